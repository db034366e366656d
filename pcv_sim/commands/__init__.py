"""`pcv-sim` subcommands. Each module has NAME, HELP, add_arguments(parser) and run(args) -> int;
list it in COMMANDS to register it. Commands render typed results from the analysis layer as
text, JSON (--json) or a plot (--plot FILE.png)."""

COMMANDS = [
    "pcv_sim.commands.static",
    "pcv_sim.commands.step",
    "pcv_sim.commands.working_points",
    "pcv_sim.commands.linearize",
    "pcv_sim.commands.replay",
    "pcv_sim.commands.import_csv",
    "pcv_sim.commands.reference_bags",
    "pcv_sim.commands.calibrate",
    "pcv_sim.commands.scenario",
    "pcv_sim.commands.campaign",
]
