"""The names of 04_nerf's files (docs/formats.md), in a module of their own: the view that reads
the folder and the code that writes it (the stage, render.py's model.pt) both import them, and
neither has to import the other for a name."""

MODEL_FILE = "model.pt"
TRAIN_LOG_FILE = "train_log.csv"
LOSS_PLOT_FILE = "loss.png"
HELDOUT_PLOT_FILE = "heldout.png"
#: Every held-out frame beside its render, with its PSNR.
HELDOUT_PAIRS_FILE = "heldout_pairs.jpg"
#: The held-out frames as the field renders them (16-bit RGB PNG, display-encoded).
HELDOUT_RGB_DIR = "heldout_rgb"
REFINED_CAMERAS_FILE = "cameras_refined.json"
