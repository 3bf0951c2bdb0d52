"""Controller selection: latent dynamics models per controller, goal scores, and the MPC selector."""
