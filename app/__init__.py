"""SemanticXR server: protocol, perception, the object-level mapping engine and the service."""

__version__ = "0.1.0"
