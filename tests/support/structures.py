"""Structure files the tests share (issue 18)."""

TRUSS_TOML = """
name = "truss"
[[modules]]
name = "tpods1"
position_m = [-0.2, 0.0]
yaw_deg = 0
[[modules]]
name = "tpods2"
position_m = [0.2, 0.05]
yaw_deg = 90
"""
"""Two modules on a truss, no [body] (the estimators start from the layout): the structure
of runs/fixtures/structure-run and of the CLI tests."""
