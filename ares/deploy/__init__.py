"""Deployment: the fleet's certificate authority and credentials, the routers' configurations,
the checks of a deployment folder, and the rehearsal across network namespaces (docs/deploy.md)."""
