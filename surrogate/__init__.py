"""pdestream.surrogate: torch models and the training loop (never imports JAX)."""
