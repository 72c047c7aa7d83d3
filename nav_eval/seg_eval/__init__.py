"""Segmentation scored on labelled photos (`segmin eval-seg`): IoU, precision, recall, contact sheets."""
