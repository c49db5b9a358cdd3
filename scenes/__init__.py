"""Scene content: the procedural mannequin (its skeleton and forward kinematics, and the collision capsules its
parts carry), its motions, skinning, garments and flat cloth pieces, and scene assembly: `registry.build_scene`
turns resolved settings into one typed `scene.Scene`, through one builder module per scene kind."""
