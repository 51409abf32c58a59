"""Segmentation heads on the frozen backbone's features: DPT, linear and UperNet, and which
settings each takes."""
