"""Commands that are not stages: export, bench, synth, batch."""
