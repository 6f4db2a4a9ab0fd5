"""Learning stability from test-cut outcomes (``robomill learn``): a Bayesian update of the tool-tip
modes and the cutting coefficients (DOMAIN.md "Learning from test cuts")."""
