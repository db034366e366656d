"""Plants that valves drive, as systems of the simulation core (`pcv_sim.simulation.system`).

`mass_spring`: a spring-loaded piston between two valve load ports (the smallest plant: the
core's composition test and the example of how a new system plugs in).
`cylinder`: the double-acting steering cylinder whose chambers are two valves' load ports
(`pcv_sim.rig`); its parameters: `pcv_sim.plant.params.CylinderParams`.
"""

__all__ = ["cylinder", "mass_spring", "params"]
