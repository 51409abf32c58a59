"""Segmentation heads on the frozen backbone's features: DPT, linear and UperNet, which settings
each takes, and the `Head` protocol they satisfy."""
