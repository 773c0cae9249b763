"""carapost.commands."""
