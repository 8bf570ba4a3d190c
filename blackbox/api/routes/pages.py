"""The web pages (ARES §3.9): served by the API itself, over the same HTTPS, with a strict
content-security policy (their own scripts and styles only, calls to this API only).

| path                     | page                                                   | role     |
|--------------------------|--------------------------------------------------------|----------|
| /operator                | the vehicle live, its map, the operator's commands     | operator |
| /blackbox                | records of a window: table, plots, CSV/JSON export     | auditor  |
| /fleet                   | every vehicle on one map, events, late vehicles        | fleet    |
| /static/...              | the pages' scripts and styles (blackbox/web/static)    |          |
| /vendor/leaflet, /uplot  | the map and plot libraries, installed from npm by the project's set-up |  |

The pages hold no data: they log in at /api/v1/auth/token and read the API with the token (a
page refuses a role it is not for, and the API refuses what the role may not read). Nothing is
fetched from the internet at run time (vehicles have patchy 4G).
"""
from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse, RedirectResponse
from starlette.staticfiles import StaticFiles

WEB = Path(__file__).resolve().parents[2] / "web"
PAGES = {"operator": "operator.html", "blackbox": "blackbox.html", "fleet": "fleet.html"}
VENDOR = {"leaflet": WEB / "node_modules" / "leaflet" / "dist", "uplot": WEB / "node_modules" / "uplot" / "dist"}
PAGE_PATHS = ("/", *(f"/{name}" for name in PAGES))
PAGE_PREFIXES = ("/static/", "/vendor/")


def mount(app: FastAPI) -> None:
    for name, file in PAGES.items():
        app.add_api_route(f"/{name}", _page(WEB / "pages" / file), methods=["GET"], include_in_schema=False)
    app.add_api_route("/", _index, methods=["GET"], include_in_schema=False)
    app.mount("/static", StaticFiles(directory=WEB / "static"), name="static")
    for lib, folder in VENDOR.items():
        # check_dir off: without the set-up's npm install the API still serves, the pages say what is missing
        app.mount(f"/vendor/{lib}", StaticFiles(directory=folder, check_dir=False), name=f"vendor-{lib}")


def _page(path: Path):
    async def page() -> FileResponse:
        return FileResponse(path, media_type="text/html; charset=utf-8")
    return page


async def _index() -> RedirectResponse:
    return RedirectResponse("/operator", status_code=307)


def vendor_missing() -> list[str]:
    """The libraries the set-up has not installed (npm)."""
    return [lib for lib, folder in VENDOR.items() if not folder.is_dir()]
