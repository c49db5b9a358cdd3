"""Scene content: the procedural mannequin (skeleton, forward kinematics, collision capsules), its motions,
skinning, garments and flat cloth pieces, and scene assembly (resolved settings -> one typed Scene)."""
