"""The web pages (ARES §3.9): served by the API itself, over the same HTTPS, with a strict
content-security policy (their own scripts and styles only, calls to this API only).

| path                     | page                                                   | role     |
|--------------------------|--------------------------------------------------------|----------|
| /operator                | the vehicle live, its map, the operator's commands     | operator |
| /blackbox                | records of a window: table, plots, CSV/JSON export     | auditor  |
| /fleet                   | every vehicle on one map, events, late vehicles        | fleet    |
| /passenger               | the next stop, the doors, why the shuttle stands       | passenger (a kiosk), operator |
| /static/...              | the pages' scripts and styles (blackbox/web/static)    |          |
| /vendor/leaflet, /uplot  | the map and plot libraries, installed from npm by the project's set-up |  |

The pages hold no data: they log in at /api/v1/auth/token and read the API with the token (a
page refuses a role it is not for, and the API refuses what the role may not read). Nothing is
fetched from the internet at run time (vehicles have patchy 4G).
"""

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, RedirectResponse
from starlette.staticfiles import StaticFiles

WEB = Path(__file__).resolve().parents[2] / "web"
VENDOR = {"leaflet": WEB / "node_modules" / "leaflet" / "dist", "uplot": WEB / "node_modules" / "uplot" / "dist"}
MAP = ("/vendor/leaflet/leaflet.css", "/vendor/leaflet/leaflet.js")
PLOTS = ("/vendor/uplot/uPlot.min.css", "/vendor/uplot/uPlot.iife.min.js")
# page -> its title and library; its content is web/pages/<page>.main.html, its script web/static/<page>.js,
# the frame around it (header, login, refusal) web/pages/frame.html
NO_LIBRARY = ("", "")
PAGES = {
    "operator": ("operator", MAP),
    "blackbox": ("black box", PLOTS),
    "fleet": ("fleet", MAP),
    "passenger": ("passenger", NO_LIBRARY),
}
PAGE_PATHS = ("/", *(f"/{name}" for name in PAGES))
PAGE_PREFIXES = ("/static/", "/vendor/")


def render(name: str) -> str:
    """A page: the frame filled with its title, library and content."""
    title, (css, js) = PAGES[name]
    page = (WEB / "pages" / "frame.html").read_text()
    if not css:  # a page without a library loads none
        page = page.replace('<link rel="stylesheet" href="{{library_css}}">\n', "")
    if not js:
        page = page.replace('<script src="{{library_js}}"></script>\n', "")
    for key, value in (
        ("main", (WEB / "pages" / f"{name}.main.html").read_text().strip()),
        ("title", title),
        ("library_css", css),
        ("library_js", js),
        ("name", name),
    ):
        page = page.replace("{{" + key + "}}", value)
    return page


def mount(app: FastAPI) -> None:
    for name in PAGES:
        app.add_api_route(f"/{name}", _page(render(name)), methods=["GET"], include_in_schema=False)
    app.add_api_route("/", _index, methods=["GET"], include_in_schema=False)
    app.mount("/static", StaticFiles(directory=WEB / "static"), name="static")
    for lib, folder in VENDOR.items():
        # check_dir off: without the set-up's npm install the API still serves, the pages say what is missing
        app.mount(f"/vendor/{lib}", StaticFiles(directory=folder, check_dir=False), name=f"vendor-{lib}")


def _page(html: str):
    async def page() -> HTMLResponse:
        return HTMLResponse(html)

    return page


async def _index() -> RedirectResponse:
    return RedirectResponse("/operator", status_code=307)


def vendor_missing() -> list[str]:
    """The libraries the set-up has not installed (npm)."""
    return [lib for lib, folder in VENDOR.items() if not folder.is_dir()]
