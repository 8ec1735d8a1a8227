"""`armbridge train`: training pipelines that end in shipped models (ONNX + card)."""
