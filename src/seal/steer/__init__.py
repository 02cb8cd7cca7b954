"""The Hypothesize -> Predict -> Verify -> Commit loop (see `engine.py`)."""
