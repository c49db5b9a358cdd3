"""The one exception type that stage CLIs turn into a clean one-line message."""


class PipelineError(Exception):
    """Bad input or configuration, raised where the input is first understood.

    The message names the file (or config key) and the problem; `pipeline.core.cli.run` prints it without a
    traceback and exits with status 2.
    """
