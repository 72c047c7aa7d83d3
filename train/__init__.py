"""Training: fit a segmentation model to data, on CPU, one GPU or many."""
