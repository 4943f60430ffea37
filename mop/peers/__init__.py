"""The field's own tools, run under mop's protocol beside mop (`mop benchmark --predictors NAME`): optional
extras that mop imports only when asked.

mop.peers.narx: sysidentpy's FROLS polynomial NARX, the library's defaults but least squares ("narx").
mop.peers.subnet: deepSI's SUBNET, the library's defaults, trained within --budget ("subnet").
mop.peers.runs: the free run both give under the protocol (free_runs).
"""
