"""ONNX export (float32, float16, int8), the file's metadata, and its runtime.

``metadata`` and ``runtime`` import no torch: a deployment reads and runs an exported file with
ONNX Runtime alone.
"""
