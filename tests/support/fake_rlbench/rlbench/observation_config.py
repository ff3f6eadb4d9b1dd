class ObservationConfig:
    pass
