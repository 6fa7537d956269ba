#!/usr/bin/env node
// Headless check of the daemon's Foxglove live view with Foxglove Studio's own app code
// (@foxglove/studio-base@1.48.0's prebuilt bundle, served from this folder on loopback).
//
// Usage:
//   node tests/browser/foxglove_check.mjs WS_URL LAYOUT_JSON MODE OUT_DIR [options]
//   node tests/browser/foxglove_check.mjs --ws ws://127.0.0.1:8765 --layout L.json --mode websocket --out DIR
// MODE (which subprotocols the page offers):
//   native     the app's own offer, nothing wrapped (studio 1.48 offers ["foxglove.websocket.v1"])
//   websocket  wrapped, offers ["foxglove.websocket.v1"]
//   sdk        wrapped, offers ["foxglove.sdk.v1"]
//   both       wrapped, offers ["foxglove.websocket.v1", "foxglove.sdk.v1"]
//   list:a,b   wrapped, offers exactly the names given
// Options:
//   --layout-method import|seed|url   import: the app's Layouts sidebar "Import layout" button (default)
//                                     seed: layout put into the shell's layout storage + user profile
//                                     url:  seeded layout selected by the app's ?layoutId= deep link
//   --new-image-panel                 turn on the app's experimental "new Image panel" setting
//   --settle SECONDS                  time to let data flow after connecting (default 12)
//   --chromium PATH                   default /usr/bin/chromium (or $CHROMIUM)
// Prints one JSON summary on stdout; screenshots, summary.json and console.log go to OUT_DIR.
// Exit status: 0 every check passed, 1 a check failed (summary.checks says which), 2 harness error.

import fs from "node:fs";
import path from "node:path";
import { createRequire } from "node:module";
import { fileURLToPath, pathToFileURL } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const appDir = here;
// scripts/setup-browser.sh installs package.json's packages into .deps/browser.
const depsDir = process.env.OP3DSG_BROWSER_DEPS || path.join(here, "../../.deps/browser");
if (!fs.existsSync(path.join(depsDir, "node_modules", "@foxglove", "studio-base"))) {
  console.error(`foxglove_check.mjs: ${depsDir}/node_modules missing: run ./scripts/setup-browser.sh (scripts/test.sh does)`);
  process.exit(2);
}
const require = createRequire(path.join(depsDir, "package.json"));
const puppeteer = require("puppeteer-core");
const { PNG } = require("pngjs");
const { startServer } = await import(pathToFileURL(path.join(appDir, "serve.mjs")).href);

// ---------------------------------------------------------------- arguments
function parseArgs(argv) {
  const o = { layoutMethod: "import", settle: 12, newImagePanel: false,
    chromium: process.env.CHROMIUM || "/usr/bin/chromium" };
  const pos = [];
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    const next = () => argv[++i];
    if (a === "--ws") o.ws = next();
    else if (a === "--layout") o.layout = next();
    else if (a === "--mode") o.mode = next();
    else if (a === "--out") o.out = next();
    else if (a === "--layout-method") o.layoutMethod = next();
    else if (a === "--settle") o.settle = Number(next());
    else if (a === "--new-image-panel") o.newImagePanel = true;
    else if (a === "--chromium") o.chromium = next();
    else if (a === "-h" || a === "--help") { console.error(fs.readFileSync(fileURLToPath(import.meta.url), "utf8").split("\n").slice(1, 24).join("\n")); process.exit(0); }
    else pos.push(a);
  }
  o.ws ??= pos[0]; o.layout ??= pos[1]; o.mode ??= pos[2]; o.out ??= pos[3];
  o.mode ??= "native";
  if (!o.ws || !o.layout || !o.out) throw new Error("usage: foxglove_check.mjs WS_URL LAYOUT_JSON MODE OUT_DIR (see --help)");
  if (!["import", "seed", "url"].includes(o.layoutMethod)) throw new Error(`bad --layout-method ${o.layoutMethod}`);
  return o;
}
const opts = parseArgs(process.argv.slice(2));
const MODES = {
  native: undefined,
  websocket: ["foxglove.websocket.v1"],
  sdk: ["foxglove.sdk.v1"],
  both: ["foxglove.websocket.v1", "foxglove.sdk.v1"],
};
let offer;
if (opts.mode.startsWith("list:")) offer = opts.mode.slice(5).split(",").filter(Boolean);
else if (opts.mode in MODES) offer = MODES[opts.mode];
else throw new Error(`bad mode ${opts.mode}`);
fs.mkdirSync(opts.out, { recursive: true });
const layoutText = fs.readFileSync(opts.layout, "utf8");
const layoutData = JSON.parse(layoutText);
const layoutName = path.basename(opts.layout, path.extname(opts.layout));

const t0 = Date.now();
const timings = {};
const mark = (k) => { timings[k] = +((Date.now() - t0) / 1000).toFixed(1); };
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
const log = (...a) => console.error(`[${((Date.now() - t0) / 1000).toFixed(1)}s]`, ...a);
const summary = { ws: opts.ws, layout: opts.layout, mode: opts.mode, offered: offer ?? "(app's own offer, unwrapped)",
  layoutMethod: opts.layoutMethod, newImagePanel: opts.newImagePanel };

// ---------------------------------------------------------------- page-side hooks (run before app code)
// 1. Subprotocol override. Studio 1.48 opens the socket inside a dedicated Worker
//    (FoxgloveWebSocketPlayer/WorkerSocketAdapter): the page posts {type:"open", data:{wsUrl, protocols}}
//    to it and the worker calls new WebSocket(wsUrl, protocols). So window.WebSocket alone is never
//    called by the app; the same replacement is applied to that message (Worker.prototype.postMessage),
//    and to window.WebSocket for the non-worker path. The worker's "open" reply carries ws.protocol:
//    recorded as the name the server answered.
function pageHooks(offer, seed) {
  const rec = (window.__op3dsgCheck = { offers: [], answered: [], wsCalls: [], workerOpens: [] });
  if (offer) {
    const NativeWS = window.WebSocket;
    class WrappedWebSocket extends NativeWS {
      constructor(url, protocols) {
        rec.wsCalls.push({ url: String(url), appOffered: protocols ?? null, sent: offer });
        super(url, offer);
      }
    }
    window.WebSocket = WrappedWebSocket;
  }
  const origPost = Worker.prototype.postMessage;
  Worker.prototype.postMessage = function (msg, ...rest) {
    if (msg && msg.type === "open" && msg.data && typeof msg.data.wsUrl === "string") {
      const entry = { url: msg.data.wsUrl, appOffered: msg.data.protocols ?? null, sent: offer ?? msg.data.protocols ?? null };
      rec.workerOpens.push(entry);
      rec.offers.push(entry.sent);
      if (offer) msg = { ...msg, data: { ...msg.data, protocols: offer } };
      this.addEventListener("message", (ev) => {
        const d = ev.data;
        if (d && d.type === "open") rec.answered.push(d.protocol);
        if (d && d.type === "close") rec.answered.push("(closed)");
      });
    }
    return origPost.call(this, msg, ...rest);
  };
  // 2. Layout import: the app's "Import layout" button calls window.showOpenFilePicker (File System
  //    Access API). Puppeteer's file-chooser interception does not serve that picker (Chromium aborts
  //    it: "Intercepted by Page.setInterceptFileChooserDialog()", which the app takes as a cancel), so
  //    the picker is answered here with the file the script hands over in window.__op3dsgPickFiles.
  const origPicker = window.showOpenFilePicker;
  window.showOpenFilePicker = async function (options) {
    const files = window.__op3dsgPickFiles;
    if (!files) return origPicker.call(window, options);
    window.__op3dsgPickFiles = undefined;
    rec.pickerCalls = (rec.pickerCalls || 0) + 1;
    return files.map(({ name, text }) => ({ kind: "file", name,
      getFile: async () => new File([text], name, { type: "application/json" }) }));
  };
  window.addEventListener("error", (e) => { (rec.errors ||= []).push(String(e.message)); });
  // 3. Optional seeding of the shell's storage (layout + app settings), before the app reads it.
  if (seed) {
    if (seed.layout) {
      const id = seed.layout.id;
      const all = JSON.parse(localStorage.getItem("op3dsg-check.layouts") || "{}");
      if (!all.local || !all.local[id]) {
        (all.local ||= {})[id] = seed.layout;
        localStorage.setItem("op3dsg-check.layouts", JSON.stringify(all));
        if (seed.selectViaProfile) localStorage.setItem("studio.profile-data", JSON.stringify({ currentLayoutId: id }));
      }
    }
    if (seed.config) {
      const cfg = JSON.parse(localStorage.getItem("op3dsg-check.app-configuration") || "{}");
      localStorage.setItem("op3dsg-check.app-configuration", JSON.stringify({ ...cfg, ...seed.config }));
    }
  }
}

// ---------------------------------------------------------------- page readers (visible text / aria)
async function clickTab(page, label) {
  // MUI tabs: role="tab"; the sidebar tabs' names are their text ("Topics", "Problems 1").
  return page.evaluate((label) => {
    const tab = [...document.querySelectorAll('[role="tab"]')].find((t) => t.textContent.trim().startsWith(label));
    if (!tab) return false;
    tab.click();
    return true;
  }, label);
}

async function readDataSource(page) {
  return page.evaluate(() => {
    const text = (el) => (el ? el.innerText.trim() : null);
    // The "Data source" sidebar: heading text "Data source"; info rows are overline labels.
    const heading = [...document.querySelectorAll("h1,h2,h3,h4,h5,h6,[class*=MuiTypography]")]
      .find((e) => e.textContent.trim() === "Data source");
    const sidebar = heading ? heading.closest("[class*=MuiStack], div")?.parentElement?.parentElement : null;
    const overline = (label) => {
      const lab = [...document.querySelectorAll("[class*=MuiTypography-overline]")]
        .find((e) => e.textContent.trim().toLowerCase() === label.toLowerCase());
      const v = lab ? lab.nextElementSibling : null;
      if (!v) return null;
      // Current source: one div per line (URL, then the server's name), each titled with its full text
      const lines = label === "Current source" ? [...v.querySelectorAll(":scope > div")] : [];
      if (lines.length) return lines.map((d) => d.getAttribute("title") ?? d.textContent.trim()).join(" | ");
      return v.innerText.trim().replace(/\s*\n\s*/g, " ");
    };
    const filter = document.querySelector('input[placeholder^="Filter by topic"]');
    const spinner = heading ? heading.parentElement?.parentElement?.querySelector('[role="progressbar"]') : null;
    const problemsTab = [...document.querySelectorAll('[role="tab"]')].find((t) => t.textContent.trim().startsWith("Problems"));
    const dsNavTab = document.querySelector('[role="tab"][title="Data source"]');
    return {
      currentSource: overline("Current source"),
      startTime: overline("Start time"),
      duration: overline("Duration"),
      // The topic filter box is enabled only while the player's presence is PRESENT.
      topicFilterEnabled: filter ? !filter.disabled : null,
      // A spinner in the sidebar header shows while INITIALIZING/RECONNECTING.
      loadingSpinner: !!spinner,
      waitingForConnection: document.body.innerText.includes("Waiting for connection…"),
      problemsTab: problemsTab ? problemsTab.textContent.trim() : null,
      navBadge: dsNavTab ? dsNavTab.innerText.trim() || null : null,
      sidebarFound: !!sidebar,
    };
  });
}

async function readTopics(page) {
  await clickTab(page, "Topics");
  await sleep(300);
  return page.evaluate(() => {
    // Each row: ListItem with data-topic / data-topic-stat counters (the app's own attributes).
    const rows = new Map();
    for (const el of document.querySelectorAll("[data-topic][data-topic-stat]")) {
      const li = el.closest("li");
      const name = el.getAttribute("data-topic");
      const r = rows.get(name) || { topic: name };
      r[el.getAttribute("data-topic-stat")] = el.textContent.trim();
      const sec = li && li.querySelector("[class*=MuiListItemText-secondary]");
      r.schema = sec ? sec.textContent.trim() : null;
      rows.set(name, r);
    }
    return [...rows.values()];
  });
}

async function readProblems(page, outDir) {
  const ok = await clickTab(page, "Problems");
  if (!ok) return { tabPresent: false, entries: [] };
  await sleep(400);
  const texts = await page.evaluate(() => {
    if ([...document.querySelectorAll("p,span,div")].some((e) => e.childElementCount === 0 && e.textContent.trim() === "No problems found")) return null;
    const tab = [...document.querySelectorAll('[role="tab"]')].find((t) => t.textContent.trim().startsWith("Problems"));
    // The list follows the tab bar in the sidebar; entries are MUI ListItemButtons (role="button").
    const root = tab.closest("[class*=MuiTabs-root]").parentElement;
    return [...root.querySelectorAll('li [role="button"]')].map((b) => b.innerText.trim());
  });
  if (texts === null) return { tabPresent: true, entries: [], text: "No problems found" };
  const entries = [];
  for (let i = 0; i < texts.length; i++) {
    // Clicking an entry opens the app's NotificationModal (role="dialog") with tip and details.
    await page.evaluate((i) => {
      const tab = [...document.querySelectorAll('[role="tab"]')].find((t) => t.textContent.trim().startsWith("Problems"));
      const root = tab.closest("[class*=MuiTabs-root]").parentElement;
      root.querySelectorAll('li [role="button"]')[i]?.click();
    }, i);
    await sleep(400);
    const detail = await page.evaluate(() => {
      const d = document.querySelector('[role="dialog"]');
      return d ? d.innerText.trim() : null;
    });
    if (i === 0) await page.screenshot({ path: path.join(outDir, "problem_detail_0.png") });
    await page.keyboard.press("Escape");
    await sleep(300);
    const topic = (texts[i].match(/ on (\/\S+)/) || [])[1] ?? null;
    entries.push({ text: texts[i], topic, detail: detail ? detail.split("\n").slice(0, 3).join("\n") : null });
  }
  return { tabPresent: true, entries };
}

async function readPanel(page, panelId) {
  return page.evaluate((panelId) => {
    const el = document.querySelector(`[data-testid="panel-mouseenter-container ${panelId}"]`);
    if (!el) {
      // UnknownPanel renders with data-testid = panel id.
      const u = document.querySelector(`[data-testid="${panelId}"]`);
      return u ? { found: true, unknown: true, text: u.innerText.trim() } : { found: false };
    }
    return { found: true, text: el.innerText.trim().slice(0, 2000) };
  }, panelId);
}

async function readPlotLegend(page, panelId) {
  return page.evaluate((panelId) => {
    const el = document.querySelector(`[data-testid="panel-mouseenter-container ${panelId}"]`);
    if (!el) return null;
    // Legend rows: a checkbox titled "Toggle visibility", then the path label, then the value.
    return [...el.querySelectorAll('[title="Toggle visibility"]')].map((cb) => {
      const row = cb.closest("div").parentElement; // listIcon div -> row (display: contents)
      const cells = [...row.children].map((c) => c.innerText.trim());
      return { label: cells[1] ?? null, value: cells[2] ?? null };
    });
  }, panelId);
}

async function dismissFirstRun(page) {
  const done = [];
  // "Open data source" start dialog (shown when no source is given): MUI Dialog, closes on Escape.
  if (await page.$('[role="dialog"]')) {
    await page.keyboard.press("Escape");
    await sleep(300);
    done.push("Open data source dialog (Escape)");
  }
  // 3D panel's onboarding tooltip "Open settings to configure topics and layers." -> [aria-label=Dismiss]
  const dismiss = await page.$('::-p-aria([name="Dismiss"][role="button"])');
  if (dismiss) {
    await dismiss.click();
    await sleep(300);
    done.push("3D settings onboarding tooltip (Dismiss)");
  }
  return done;
}

async function shotElement(page, selector, file) {
  const el = await page.$(selector);
  if (!el) return null;
  await el.screenshot({ path: file });
  return file;
}

function dominantColour(png) {
  const counts = new Map();
  for (let i = 0; i < png.data.length; i += 4) {
    const k = ((png.data[i] >> 3) << 10) | ((png.data[i + 1] >> 3) << 5) | (png.data[i + 2] >> 3);
    counts.set(k, (counts.get(k) || 0) + 1);
  }
  let best = 0, bestN = -1;
  for (const [k, n] of counts) if (n > bestN) { best = k; bestN = n; }
  return { rgb: [((best >> 10) & 31) * 8 + 4, ((best >> 5) & 31) * 8 + 4, (best & 31) * 8 + 4], fraction: +(bestN / (png.data.length / 4)).toFixed(3) };
}

// Two figures: the raw per-pixel difference, and the same after the uniform backdrop change is
// discounted (the empty grid's background colour is taken to be the live picture's background
// colour, e.g. the occupancy map's tint of unknown cells), which leaves what the scene draws.
function pixelDiff(fileA, fileB, fileOut) {
  const a = PNG.sync.read(fs.readFileSync(fileA));
  const b = PNG.sync.read(fs.readFileSync(fileB));
  if (a.width !== b.width || a.height !== b.height) return { error: `size differs ${a.width}x${a.height} vs ${b.width}x${b.height}` };
  const bgA = dominantColour(a), bgB = dominantColour(b);
  const out = new PNG({ width: a.width, height: a.height });
  const T = 32;
  let changed = 0, changedBg = 0, sumAbs = 0;
  const n = a.width * a.height;
  const near = (d, i, c) => Math.abs(d[i] - c[0]) <= 12 && Math.abs(d[i + 1] - c[1]) <= 12 && Math.abs(d[i + 2] - c[2]) <= 12;
  for (let i = 0; i < n * 4; i += 4) {
    let d = 0, s = 0;
    for (let c = 0; c < 3; c++) { const x = Math.abs(a.data[i + c] - b.data[i + c]); d = Math.max(d, x); s += x; }
    sumAbs += s / 3;
    if (d > T) changed++;
    // backdrop-discounted: a background pixel of the empty grid counts as the live background
    let d2 = d;
    if (near(a.data, i, bgA.rgb)) { d2 = 0; for (let c = 0; c < 3; c++) d2 = Math.max(d2, Math.abs(bgB.rgb[c] - b.data[i + c])); d2 = Math.max(0, d2 - 8); }
    const hit = d2 > T;
    if (hit) changedBg++;
    const g = (b.data[i] + b.data[i + 1] + b.data[i + 2]) / 9;
    out.data[i] = hit ? 255 : (d > T ? 255 : g); out.data[i + 1] = hit ? 0 : (d > T ? 200 : g); out.data[i + 2] = hit ? 0 : g; out.data[i + 3] = 255;
  }
  fs.writeFileSync(fileOut, PNG.sync.write(out));
  return { width: a.width, height: a.height, threshold: `max channel diff > ${T} of 255`,
    changedPixels: changed, changedFraction: +(changed / n).toFixed(4), meanAbsDiff: +(sumAbs / n).toFixed(2),
    backgroundEmpty: bgA, backgroundLive: bgB,
    sceneChangedPixels: changedBg, sceneChangedFraction: +(changedBg / n).toFixed(4),
    diffImage: "red: differs after discounting the backdrop change; yellow: differs only through the backdrop" };
}

async function waitFor(fn, timeoutMs, stepMs = 500) {
  const end = Date.now() + timeoutMs;
  for (;;) {
    const v = await fn();
    if (v || Date.now() > end) return v;
    await sleep(stepMs);
  }
}

// ---------------------------------------------------------------- run
const server = await startServer(0);
const base = `http://127.0.0.1:${server.address().port}/`;
mark("serverUp");
const browser = await puppeteer.launch({
  executablePath: opts.chromium,
  headless: true,
  args: [
    "--no-sandbox", // running as root: Chromium refuses to start without it
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader", // WebGL on CPU for the 3D panel
    "--window-size=1600,1000",
  ],
  defaultViewport: { width: 1600, height: 1000 },
});
mark("browserUp");
const consoleLines = [];
const pageErrors = [];
let exitCode = 0;
try {
  const ctx = await browser.createBrowserContext(); // fresh storage per run
  const page = await ctx.newPage();
  page.on("console", (m) => { const t = `${m.type()}: ${m.text()}`; consoleLines.push(t); });
  page.on("pageerror", (e) => pageErrors.push(String(e.message ?? e)));
  page.on("workercreated", (w) => consoleLines.push(`worker: ${w.url()}`));

  const layoutId = "op3dsg-live-layout";
  const now = new Date().toISOString();
  const seedLayout = { id: layoutId, name: layoutName, permission: "CREATOR_WRITE",
    baseline: { data: layoutData, savedAt: now }, working: undefined, syncInfo: undefined };
  const seed = { config: {} };
  if (opts.newImagePanel) seed.config.enableNewImagePanel = true;
  if (opts.layoutMethod === "seed") Object.assign(seed, { layout: seedLayout, selectViaProfile: true });
  if (opts.layoutMethod === "url") Object.assign(seed, { layout: seedLayout, selectViaProfile: false });
  await page.evaluateOnNewDocument(pageHooks, offer, seed);

  // For the import method: the app calls window.showOpenFilePicker (File System Access API).
  // Puppeteer's file-chooser interception is tried first; see README for what happened.
  const layoutQuery = opts.layoutMethod === "url" ? `?layoutId=${layoutId}` : "";
  // --- Phase 1: no data source: the layout with an empty grid (the baseline picture).
  await page.goto(base + layoutQuery, { waitUntil: "load" });
  await page.waitForFunction(() => document.querySelector('[data-testid^="panel-mouseenter-container"]'), { timeout: 60000 });
  mark("appRendered");
  summary.firstRunDismissed = await dismissFirstRun(page);

  if (opts.layoutMethod === "import") {
    const layoutsTab = await page.waitForSelector('::-p-aria([name="Layouts"][role="tab"])', { timeout: 10000 });
    await layoutsTab.click();
    const importBtn = await page.waitForSelector('::-p-aria([name="Import layout"][role="button"])', { timeout: 10000 });
    await page.evaluate((name, text) => { window.__op3dsgPickFiles = [{ name, text }]; },
      path.basename(opts.layout), layoutText);
    await importBtn.click();
    const imported = await waitFor(() => page.$('[data-testid="panel-mouseenter-container 3D!op3dsg"]'), 10000);
    const pickerCalls = await page.evaluate(() => window.__op3dsgCheck.pickerCalls || 0);
    summary.layoutImport = { via: "Layouts sidebar > 'Import layout' button, showOpenFilePicker answered by the page hook",
      pickerCalls, layoutPanelsAppeared: !!imported };
    // back to the Data source sidebar
    const dsTab = await page.$('::-p-aria([name="Data source"][role="tab"])');
    if (dsTab) await dsTab.click();
  }
  summary.layoutLoaded = await page.evaluate(() => [...new Set(
    [...document.querySelectorAll('[data-testid^="panel-mouseenter-container"]')]
      .map((e) => e.getAttribute("data-testid").replace("panel-mouseenter-container ", "")))]);
  await sleep(3000); // let the 3D panel draw the grid
  summary.firstRunDismissed.push(...(await dismissFirstRun(page)));
  await page.screenshot({ path: path.join(opts.out, "1_no_source.png") });
  const canvas3d = '[data-testid="panel-mouseenter-container 3D!op3dsg"] canvas';
  const emptyShot = await shotElement(page, canvas3d, path.join(opts.out, "3d_empty_grid.png"));
  mark("baselineTaken");

  // --- Phase 2: connect through the app's deep link (?ds=foxglove-websocket&ds.url=...)
  const q = new URLSearchParams();
  q.set("ds", "foxglove-websocket");
  q.set("ds.url", opts.ws);
  if (opts.layoutMethod === "url") q.set("layoutId", layoutId);
  await page.goto(`${base}?${q}`, { waitUntil: "load" });
  await page.waitForFunction(() => document.querySelector('[data-testid^="panel-mouseenter-container"]'), { timeout: 60000 });
  const connected = await waitFor(async () => (await readDataSource(page)).topicFilterEnabled === true, 20000);
  mark(connected ? "connected" : "connectWaitEnded");
  await sleep(opts.settle * 1000);
  summary.firstRunDismissed.push(...(await dismissFirstRun(page)));
  await sleep(1500);

  const ds = await readDataSource(page);
  const hooks = await page.evaluate(() => window.__op3dsgCheck);
  summary.subprotocol = { offeredByPage: hooks.offers, serverAnswered: hooks.answered,
    appOfferedBeforeWrap: hooks.workerOpens.map((o) => o.appOffered), windowWebSocketCalls: hooks.wsCalls.length };
  summary.connection = { ...ds, up: ds.topicFilterEnabled === true && !ds.loadingSpinner && !ds.waitingForConnection };
  await page.screenshot({ path: path.join(opts.out, "2_connected.png") });
  const liveShot = await shotElement(page, canvas3d, path.join(opts.out, "3d_live.png"));
  summary.topics = await readTopics(page);
  summary.problems = await readProblems(page, opts.out);
  await page.screenshot({ path: path.join(opts.out, "3_problems.png") });
  await clickTab(page, "Topics");
  summary.threeD = { panel: (await readPanel(page, "3D!op3dsg")).found };
  if (emptyShot && liveShot) summary.threeD.diffVsEmptyGrid = pixelDiff(emptyShot, liveShot, path.join(opts.out, "3d_diff.png"));
  summary.imagePanel = await readPanel(page, "Image!op3dsg");
  const plot = await readPanel(page, "Plot!op3dsg-health");
  const legend = await readPlotLegend(page, "Plot!op3dsg-health");
  await shotElement(page, '[data-testid="panel-mouseenter-container Plot!op3dsg-health"]', path.join(opts.out, "plot.png"));
  summary.plot = { found: plot.found, legend, healthValueShown: !!legend && legend.some((r) => r.value !== null && r.value !== "" && !Number.isNaN(Number(r.value))) };
  const EXPECTED = { "/op3dsg/scene": "foxglove.SceneUpdate", "/op3dsg/occupancy": "foxglove.Grid",
    "/tf": "foxglove.FrameTransform", "/op3dsg/health": "op3dsg.Health" };
  const byName = Object.fromEntries(summary.topics.map((t) => [t.topic, t.schema]));
  const d3 = summary.threeD.diffVsEmptyGrid;
  summary.checks = {
    connectionUp: summary.connection.up,
    topicsWithSchemas: Object.entries(EXPECTED).every(([t, sch]) => byName[t] === sch),
    missingTopics: Object.entries(EXPECTED).filter(([t, sch]) => byName[t] !== sch).map(([t, sch]) => `${t} (${sch})`),
    noProblems: summary.problems.entries.length === 0,
    problems: summary.problems.entries.map((e) => e.text),
    sceneDrawn: !!d3 && d3.sceneChangedFraction > 0.01,
    plotHasHealthValue: summary.plot.healthValueShown,
    imagePanel: summary.imagePanel.text?.startsWith("Unknown panel type") ? summary.imagePanel.text : (summary.imagePanel.found ? "rendered" : "missing"),
  };
  summary.pass = ["connectionUp", "topicsWithSchemas", "noProblems", "sceneDrawn", "plotHasHealthValue"].every((k) => summary.checks[k]);
  if (!summary.pass) exitCode = 1;
  summary.pageErrors = [...new Set(pageErrors)].slice(0, 20);
  summary.consoleErrors = [...new Set(consoleLines.filter((l) => l.startsWith("error")))].slice(0, 20);
  mark("done");
  summary.timings_s = timings;
  summary.screenshots = fs.readdirSync(opts.out).filter((f) => f.endsWith(".png")).map((f) => path.join(opts.out, f));
} catch (err) {
  summary.fatal = String(err.stack ?? err);
  summary.pageErrors = pageErrors.slice(0, 20);
  exitCode = 2;
} finally {
  fs.writeFileSync(path.join(opts.out, "console.log"), consoleLines.join("\n") + "\n");
  fs.writeFileSync(path.join(opts.out, "summary.json"), JSON.stringify(summary, null, 2) + "\n");
  await browser.close();
  server.close();
}
console.log(JSON.stringify(summary, null, 2));
process.exit(exitCode);
