"""The device emulator: frame sources, encoder, streaming client, local map, querying."""
