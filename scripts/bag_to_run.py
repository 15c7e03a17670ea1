"""Snakemake script: ROS 2 bag (MCAP) -> measurement run (sim2real.measurements.bags.mcap_to_run)."""

from sim2real.cli import rule_entry
from sim2real.measurements.bags import mcap_to_run

with rule_entry(snakemake):
    mcap_to_run(
        snakemake.input.bag,
        snakemake.output.run,
        robot=snakemake.wildcards.robot,
        joint_topic=snakemake.params.topics["joint_topic"],
        command_topic=snakemake.params.topics["command_topic"],
        torque_sensor=snakemake.params.topics["torque_sensor"],
    )
