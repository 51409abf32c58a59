"""The datasets and what they are built from: the frame index (``index``), spatial blocks and
splits (``blocks``, ``splits``), palettes and label masks of real datasets (``palettes``,
``masks``), the label cache and ``claravid-cache`` (``label_cache``, its entries on disk
``cache_entries``, preparing them ``cache_prepare``, ``cache_cli``), the torch
Datasets (``segmentation``, ``targets``, the official-SDK drop-in ``sdk``), samples and
augmentations (``samples``, ``transforms``) and pictures of samples (``plot``).

Reads files through ``claravid.io``; knows nothing of models, training or complexity.
"""
