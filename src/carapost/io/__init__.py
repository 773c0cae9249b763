"""carapost.io."""
