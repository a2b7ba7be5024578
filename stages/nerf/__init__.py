"""The nerf stage (docs/formats.md): field, sampling, rendering, losses, training.

Import the stage from `endopipe.stages.nerf.stage`: this package imports nothing, so inference
(render, baked, the depth stage) does not load the training code.
"""
