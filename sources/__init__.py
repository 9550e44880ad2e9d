"""Built-in sources: files, the moving pattern, and (in later modules)
devices, the network and the simulator."""
