"""Simulation layer: the MJX physics backends, the robot model resolved by name, substepping, C MuJoCo
substeps, CPU and GL set-up."""
