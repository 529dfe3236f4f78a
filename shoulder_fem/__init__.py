"""shoulder-fem: large motions with small strains, coupled and decoupled."""
__version__ = "0.1.0"
