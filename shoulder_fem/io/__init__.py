"""Output folders and summaries, resources, comparisons, plots, CT images."""
