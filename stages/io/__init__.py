"""Readers that turn inputs (video, image folder, case folder, datasets) into frames."""
