"""Several nodes or commands at once: the whole graph, launch files, hosts, shutdown."""
