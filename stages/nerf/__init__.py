"""The nerf stage (DESIGN §3 `04_nerf/`): field, sampling, rendering, losses, training.

Import the stage from `endopipe.stages.nerf.stage`: this package imports nothing, so inference
(render, baked, the depth stage) does not load the training code.
"""
