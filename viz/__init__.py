"""Pictures and files a person can look at, none needing a display: shaded renders of cloth on a body (render.py,
on raster.py's numpy z-buffer), one frame of cloth upsampling as input | truth | network | error panels
(comparison.py), animations of rendered frames (animation.py: MP4 or GIF), report plots (plots.py), a
self-contained HTML report and the same pieces as markdown (html_report.py, markdown_report.py), and OBJ/GLB
export through trimesh (export.py). No module here writes a final output by itself except render_panels and
export: each returns bytes or text for the caller's atomic writer."""
