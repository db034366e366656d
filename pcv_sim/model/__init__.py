"""The valve model: the paper's equations, SI units (x in mm for the fits only). `kernel` holds
the valve over arrays, compiled for the simulation core; `solenoid`, `orifice` and `flow_force`
the equation functions it calls; `valve` and `statics` serve the same equations to the analysis.
Knows nothing about ROS or integrators."""
