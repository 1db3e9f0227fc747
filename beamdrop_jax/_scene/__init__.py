"""The scene: its containers and checks (`containers.py`) and scene files (`file.py`)."""
