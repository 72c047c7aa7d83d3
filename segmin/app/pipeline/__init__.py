"""`segmin pipeline`: rendered worlds -> trained models -> ONNX -> closed-loop report, cached per stage."""
