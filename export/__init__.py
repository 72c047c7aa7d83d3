"""Export: a deployable, verified ONNX file for embedded targets."""
