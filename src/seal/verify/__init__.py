"""Who judges: verifiers decide whether a predicted outcome matches a sub-plan."""
