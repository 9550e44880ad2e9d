"""Built-in sinks: files, and (in later modules) display and network."""
