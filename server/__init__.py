"""fleet-server: the cloud server of fleet-cloud."""
