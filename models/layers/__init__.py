"""Building blocks of the ViT backbones: attention, RoPE, transformer blocks, and shape-generic
helpers for tracing."""
