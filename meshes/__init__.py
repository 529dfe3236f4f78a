"""gmsh / dolfinx mesh builders, one per scene family."""
