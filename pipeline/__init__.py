"""signpose's computer vision: framework-free stages over numpy arrays (numpy + OpenCV only)."""
