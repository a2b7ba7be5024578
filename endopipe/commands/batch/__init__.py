"""`endopipe batch`: every case under a folder through the pipeline, on a local pool, Slurm or
Ray (the engine's executors), gathered into batch.csv and batch.html.

- `rows`: what a job gets (`CaseTask`) and what it gives back (`CaseRow`).
- `case`: the job itself, one case in whatever process or cluster job runs it.
- `driver`: sends the cases with work left to an executor; a crashed job is a failed row.
- `table` / `page`: batch.csv and the self-contained batch.html.
- `command`: the command's body, from a folder to the written table.
"""

from endopipe.commands.batch.rows import CaseRow, CaseTask

__all__ = ["CaseRow", "CaseTask"]
