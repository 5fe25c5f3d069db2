"""The plant: model (rigid body, thrusters, optional effects, analytic Jacobians), propagation, inputs, simulator, orbit-follower controller, named parameter sets."""
