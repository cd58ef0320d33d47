"""The one error type for bad input from the network or a device."""


class InputError(ValueError):
    """Bad input; `field` names what is wrong (e.g. "depth", "detections.instances[2].label").

    Whatever raised it left every map and session exactly as they were.
    """

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message
