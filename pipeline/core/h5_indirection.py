"""Refusing HDF5 files that reach outside themselves.

HDF5 can make a dataset's bytes come from elsewhere: an external link names an object in another HDF5 file, a
virtual dataset maps other files' datasets into its own, and external storage reads a dataset's raw bytes from
any file at all (a `sim_low.h5` whose positions were stored "in" /etc/passwd once carried that file's bytes into
dataset.h5). libhdf5 follows all three silently on read, so an artifact from elsewhere could make a stage read,
and copy into its output, files the user never named. No stage writes any of them, so every artifact that holds
one is refused when it is opened, before anything is read from it.
"""
from __future__ import annotations

import h5py

from pipeline.core.errors import PipelineError


def refuse_indirection(f: h5py.File) -> None:
    """One error naming the file and the first object that takes its data from another file. Walks the links
    once (names and link types, each dataset's creation properties: no data is read); soft links stay inside the
    file and are allowed, since every object they can reach is walked too."""
    problem = f.visititems_links(lambda name, link: _reaches_out(f, name, link))
    if problem is not None:
        raise PipelineError(f"{f.filename}: {problem}; an artifact must hold its own data")


def _reaches_out(f: h5py.File, name: str, link: h5py.HardLink | h5py.SoftLink | h5py.ExternalLink) -> str | None:
    # The names are the file's own, so they are shown escaped and cut short: a message stays one line.
    shown = ascii(name[:80])
    if isinstance(link, h5py.ExternalLink):
        return f"{shown} is an external link to another file"
    if not isinstance(link, h5py.HardLink):
        return None
    target = f[name]
    if isinstance(target, h5py.Dataset) and target.is_virtual:
        return f"dataset {shown} is a virtual dataset (its data lies in other files)"
    if isinstance(target, h5py.Dataset) and target.external:
        return f"dataset {shown} keeps its data in external files"
    return None
