"""`endopipe batch`: every case under a folder through the pipeline as jobs (`endopipe.jobs`) on
a local pool, Slurm or Ray, gathered into batch.csv and batch.html.

- `command`: the command's body, from a folder to the written table; a long input is handed to
  the recording command the composition root passes in (batch never imports it).
- `table` / `page`: batch.csv and the self-contained batch.html.
"""
