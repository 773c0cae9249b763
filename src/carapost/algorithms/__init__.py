"""carapost.algorithms."""
