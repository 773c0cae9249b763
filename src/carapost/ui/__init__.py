"""carapost.ui."""
