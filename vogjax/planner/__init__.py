"""Next-best-view exploration (placeholder package: being built)."""
