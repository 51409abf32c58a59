"""The backbones: one ViT trunk that DINOv2 and DINOv3 share, each family's token preparation and
positions, the named descriptions, building one with weights, and the `Backbone` protocol."""
