"""Any LeRobot policy checkpoint as a controller of the library."""
