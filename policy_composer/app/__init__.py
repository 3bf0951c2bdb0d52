"""The application: the `policy-composer` command line, the main job and its report, the recording driver,
Table I, composed runs and the MDP experiments; everything below it is a library."""
