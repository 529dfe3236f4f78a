"""The two pipelines: coupled (method #1) and decoupled (method #2)."""
