"""carapost.synth."""
