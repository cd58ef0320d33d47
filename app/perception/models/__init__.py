"""The `models` perception backend: open-vocabulary detection and CLIP embeddings from pixels.

`weights` (which models, from where; light), `masks` (pure numpy), `detector` (OWL-ViT),
`embedder` (CLIP's towers), `backend` (the keyframe pipeline), `tiny` (small random models
of the same architectures for tests). Importing this package loads no model library.
"""
