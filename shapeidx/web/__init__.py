"""``shapeidx serve``: the local web page and JSON API over a store (see docs/web.md).

    app.py       StoreService (the store in memory) and the Starlette application
guard.py     every request as hostile: Host, Origin, header sizes, time limits
    static/      the page: index.html, app.js, style.css
"""
