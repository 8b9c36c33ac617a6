"""The `/v1` API and the health check, one router per resource."""
