"""What every scene uses: solvers, rigid motion, mass properties, springs, contact.

SNES and load stepping, SO(3) and rigid dynamics, rigid bodies inside FE models, contact, the
floating-frame solver.
"""
