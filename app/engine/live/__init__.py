"""The live engine: its background thread and the commands it applies (worker), its parts as one
typed bundle (parts) and where its output goes (publisher)."""
