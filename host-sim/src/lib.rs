//! The simulated rig: a physical plant and a board that runs the firmware's own tasks.
