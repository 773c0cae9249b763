"""carapost.model."""
