"""Recordings: a long video as overlapping windows of keyframes, each a case through the same
stages (sent to the engine's executors like batch's cases), joined into one trajectory."""
