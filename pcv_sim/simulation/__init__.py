"""Running the model in time: fixed-step real-time stepping, stiff reference solutions, inputs."""
