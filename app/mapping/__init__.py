"""The object-level mapping engine: geometry, association, merge, deltas, query."""
