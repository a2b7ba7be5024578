"""The mesh stage's summary, one model on both sides: the stage writes it into its manifest,
`MeshView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from endopipe.pipeline.stage import Summary


class MeshSummary(Summary):
    method: str
    vertices: int
    faces: int
    voxel_size: float
    depth_trunc: float
    frames_used: int
    units: str
    build_s: float
    clean_s: float
    evaluated: bool = False
    chamfer: float | None = None
    chamfer_pct_radius: float | None = None
    accuracy: float | None = None
    completeness: float | None = None
    fscore: float | None = None
    threshold: float | None = None
    aligned: str | None = None
    off_seen_pct: float | None = None  # share of the mesh far from any surface a camera saw
    #: a scene that moves: the frames with a surface of their own in times/ (mesh.times)
    time_frames: list[int] = []
