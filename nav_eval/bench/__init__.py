"""`segmin bench navigator`: the navigators and the robot runtime per frame, on the robot's own computer."""
