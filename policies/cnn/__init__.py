"""The visual behaviour-cloned policy (paper: CNN): a convolutional encoder of one camera image plus the arm's
joint angles, and a mixture density head over the next joint targets. LeRobot's layout: configuration,
modeling, training, and the controller that runs it."""
