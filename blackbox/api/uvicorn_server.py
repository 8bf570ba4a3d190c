"""Running the API under uvicorn: over HTTPS unless plain HTTP is asked for explicitly."""

import logging
from pathlib import Path

from fastapi import FastAPI

from blackbox.api.app import create_app
from blackbox.api.settings import PREFIX, ApiSettings
from blackbox.register.store.open_store import open_store
from blackbox.register.store.record_store import StoreSettings

log = logging.getLogger(__name__)


def uvicorn_config(
    app: FastAPI,
    settings: ApiSettings,
    *,
    insecure_http: bool = False,
    host: str | None = None,
    port: int | None = None,
):
    """uvicorn's configuration for `app`: TLS with the configured or self-signed certificate,
    unless `insecure_http` (explicit: tokens and records would cross the network in clear).
    TLS and HTTP are served by blackbox.api.connections' protocols: a cap per address and
    timeouts on the handshake, the headers and the body."""
    import uvicorn

    from blackbox.api.connections import protocol_factory, server_tls_context

    tls = None
    if not insecure_http:
        from blackbox.api.tls import certificate

        tls = server_tls_context(*certificate(settings.tls, app.state.state_dir))
    return uvicorn.Config(
        app,
        host=host or settings.host,
        port=settings.port if port is None else port,
        loop="uvloop",
        http=protocol_factory(settings.connections, tls),
        lifespan="off",
        access_log=settings.access_log,
        log_level=settings.log_level,
        proxy_headers=False,
        server_header=False,
        timeout_keep_alive=settings.keep_alive_s,
        limit_concurrency=settings.limit_concurrency,
    )


def serve(
    settings: ApiSettings,
    store_uri: str | None = None,
    *,
    vehicle_id: str,
    store_settings: StoreSettings = StoreSettings(),
    insecure_http: bool = False,
    host: str | None = None,
    port: int | None = None,
    snapshots_dir: Path | None = None,
) -> None:
    """Run the API in the foreground until interrupted (uvicorn handles SIGINT/SIGTERM); the
    incident snapshots it serves are in `snapshots_dir`."""
    import uvicorn

    store = open_store(store_uri, settings=store_settings)
    try:
        app = create_app(store, settings, vehicle_id, snapshots_dir=snapshots_dir)
        config = uvicorn_config(app, settings, insecure_http=insecure_http, host=host, port=port)
        if insecure_http:
            log.warning("REST API over plain HTTP (--insecure-http): tokens and records travel in clear")
        scheme = "http" if insecure_http else "https"
        print(
            f"ARES black box API on {scheme}://{config.host}:{config.port}{PREFIX} (state in {app.state.state_dir})",
            flush=True,
        )
        uvicorn.Server(config).run()
    finally:
        store.close()
