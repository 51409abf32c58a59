"""Models: DINOv2 ViT backbones in plain PyTorch, the DPT segmentation decoder, ONNX export."""
