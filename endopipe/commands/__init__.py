"""The commands' bodies (run, status, clean, stages, synth, demo, bench, batch, export) and the
libraries only commands use (the synthetic-case generator, the bench, the exporters); the cli
declares their options and hands them the pipeline."""
