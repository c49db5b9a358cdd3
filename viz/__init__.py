"""Pictures and files a person can look at: shaded PNG renders of triangle meshes (matplotlib, no display
needed), side-by-side panels with per-vertex error colouring, and OBJ/GLB export through trimesh."""
