class EndEffectorPoseViaPlanning:
    pass
