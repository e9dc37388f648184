"""Running combinations over datasets: grid expansion, execution, and the per-frame results store."""
