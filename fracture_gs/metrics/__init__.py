"""Image and reconstruction quality metrics."""
