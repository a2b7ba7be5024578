"""endopipe's engine: stages, configs, caches and executors. Knows nothing of endoscopy."""
