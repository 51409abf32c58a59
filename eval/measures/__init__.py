"""Per-image (and per-pair) sums: confusions, Boundary IoU, calibration bins and cross-view
consistency.

Every measure is a sum per image, so bins, merges, the bootstrap and paired comparisons treat
them alike.
"""
