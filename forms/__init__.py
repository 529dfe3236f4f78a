"""Pure UFL forms: kinematics, materials, virtual-power terms and rigid-body functionals."""
