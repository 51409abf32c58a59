"""Backbone weights: one loader for every format people download, each family's key renames as
data, and hub ids through ``huggingface_hub``'s cache."""
