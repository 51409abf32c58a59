"""Analysis (numpy only: no torch, no files): every number of a report, from per-image tables.

``table`` (the per-image table and merging), ``metrics`` (IoU, mIoU, pixel accuracy),
``measures`` (the complexity measures), ``bins`` (quantile and fixed bins), ``units`` (groups
and bootstrap clusters), ``bootstrap`` (cluster percentile intervals), ``stats``
(correlations, profiles, order checks), ``miou_bins`` (mIoU per bin and group), ``tile_bins``
(tiles' bins), ``quality_table``, ``quality`` and ``sum_intervals`` (Boundary IoU, calibration
and cross-view consistency as per-image sums, their statistics and intervals), ``compare``
(gaps between reports) and ``metric_bins`` (any per-image metric).
Saved reports are re-binned, merged and compared here without a model or torch.
"""
