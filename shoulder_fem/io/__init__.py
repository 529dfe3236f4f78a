"""Atomic output, run summaries, XDMF fields, resources, comparisons, plots, CT images."""
