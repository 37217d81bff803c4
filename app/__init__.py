"""signpose's front ends: the CLI, the FastAPI server and the viser scene."""
