"""Who acts: action sources and reasoning policies."""
