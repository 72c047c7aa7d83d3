"""Data: turn files on disk (AgriSeg or rendered worlds) into aligned image/mask samples."""
