"""Running an experiment's node graph: the nodes it launches (launches, start_scripts), their
processes (node_graph), the runner's own observers (observers), one run (runner, with
run_options), and the e-stop command (estop_command).
"""
