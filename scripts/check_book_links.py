"""Checks every link of the built user guide (mdBook's HTML): a link inside the book must name a
page that exists and, with `#anchor`, an element with that id on it; an image must exist. Links to
other sites are listed, not fetched (CI has no network to the world).

Usage: check_book_links.py BOOK_DIR      (exit 1 when any link is broken; each named with its page)
"""
import html.parser
import pathlib
import sys
import urllib.parse


class Page(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.links = []  # (attribute, value)
        self.ids = set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name == "id" and value:
                self.ids.add(value)
            if value and ((tag == "a" and name == "href") or (tag == "img" and name == "src")):
                self.links.append(value)


def parse(path, cache):
    if path not in cache:
        page = Page()
        page.feed(path.read_text(encoding="utf-8"))
        cache[path] = page
    return cache[path]


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    book = pathlib.Path(sys.argv[1]).resolve()
    pages = sorted(p for p in book.rglob("*.html") if p.name not in ("print.html", "toc.html", "404.html"))
    if not pages:
        print(f"no pages in {book}: build the book first", file=sys.stderr)
        return 2
    cache, broken, checked, external = {}, [], 0, set()
    for page_path in pages:
        for link in parse(page_path, cache).links:
            url = urllib.parse.urlparse(link)
            if url.scheme in ("http", "https", "mailto"):
                external.add(link)
                continue
            if url.scheme or link.startswith("javascript:"):
                continue
            checked += 1
            target = page_path if not url.path else (page_path.parent / urllib.parse.unquote(url.path)).resolve()
            if target.is_dir():
                target = target / "index.html"
            where = page_path.relative_to(book)
            if not target.is_file() or book not in target.parents:
                broken.append(f"{where}: {link}: no such file in the book")
                continue
            if url.fragment and target.suffix == ".html":
                if urllib.parse.unquote(url.fragment) not in parse(target, cache).ids:
                    broken.append(f"{where}: {link}: no #{url.fragment} on {target.relative_to(book)}")
    for b in broken:
        print("broken link:", b)
    print(f"[book] {len(pages)} pages, {checked} links inside the book checked, {len(broken)} broken; "
          f"{len(external)} links to other sites not fetched")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
