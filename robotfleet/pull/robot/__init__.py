"""What runs on a pull robot: one wake of the agent (fetch, verify, decide,
prepare, converge, report).  Never imports the operator's side."""
