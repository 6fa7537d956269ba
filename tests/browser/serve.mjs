// Static server for the Foxglove shell, loopback only. Usage: node serve.mjs [port]  (0 = free port)
import http from "node:http";
import fs from "node:fs";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
// scripts/setup-browser.sh installs package.json's packages there.
const nm = process.env.OP3DSG_BROWSER_DEPS
  ? path.join(process.env.OP3DSG_BROWSER_DEPS, "node_modules")
  : path.join(here, "../../.deps/browser/node_modules");
const ROUTES = [
  ["/vendor/react.production.min.js", path.join(nm, "react/umd/react.production.min.js")],
  ["/vendor/react-dom.production.min.js", path.join(nm, "react-dom/umd/react-dom.production.min.js")],
  ["/studio/", path.join(nm, "@foxglove/studio-base/assets/")],
  ["/", path.join(here, "web/")],
];
const TYPES = { ".js": "text/javascript", ".html": "text/html", ".wasm": "application/wasm", ".png": "image/png",
  ".ttf": "font/ttf", ".woff2": "font/woff2", ".css": "text/css", ".json": "application/json", ".svg": "image/svg+xml" };

export function startServer(port = 0, host = "127.0.0.1") {
  const server = http.createServer((req, res) => {
    let p = decodeURIComponent(new URL(req.url, "http://x").pathname);
    if (p === "/") p = "/index.html";
    for (const [prefix, target] of ROUTES) {
      if (prefix.endsWith("/") ? p.startsWith(prefix) : p === prefix) {
        const file = prefix.endsWith("/") ? path.join(target, p.slice(prefix.length)) : target;
        if (!file.startsWith(target.endsWith("/") ? target : path.dirname(target))) break;
        fs.stat(file, (err, st) => {
          if (err || !st.isFile()) { res.writeHead(404); res.end("not found"); return; }
          res.writeHead(200, { "Content-Type": TYPES[path.extname(file)] || "application/octet-stream",
            "Content-Length": st.size, "Cache-Control": "no-cache" });
          fs.createReadStream(file).pipe(res);
        });
        return;
      }
    }
    res.writeHead(404); res.end("not found");
  });
  return new Promise((resolve) => server.listen(port, host, () => resolve(server)));
}

if (process.argv[1] === fileURLToPath(import.meta.url)) {
  const s = await startServer(Number(process.argv[2] ?? 8080));
  console.log(`serving http://127.0.0.1:${s.address().port}/`);
}
