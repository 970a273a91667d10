// Headless-Chromium check of `nerf view` / `nsff view`, as a person would use it: open the page,
// wait for the coarse and the refined frame, screenshot; drag to orbit, screenshot; for NSFF move
// the time slider, screenshot. Prints the times to the first coarse and refined frame and whether
// each action changed the picture.
//
//   npm install playwright-core            (in any scratch folder; uses Debian's /usr/bin/chromium)
//   nerf view RUN_DIR --port 7007 &        (or nsff view)
//   node docs/viewer/check.mjs http://127.0.0.1:7007/ docs/viewer/nerf [--time]
import { chromium } from "playwright-core";

const [url, prefix, timeFlag] = process.argv.slice(2);
const browser = await chromium.launch({
  executablePath: "/usr/bin/chromium",
  args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync"],
});
const page = await browser.newPage({ viewport: { width: 760, height: 620 } });
const newFrame = (old, state) => page.waitForFunction(
  ([o, s]) => { const v = document.getElementById("view"); return v.src !== o && v.dataset.state === s; },
  [old, state], { timeout: 300000 });
const src = () => page.$eval("#view", e => e.src);

const t0 = Date.now();
await page.goto(url);
await newFrame("", "coarse");
const coarseMs = Date.now() - t0;
await newFrame(await src(), "refined");
const refinedMs = Date.now() - t0;
await page.screenshot({ path: `${prefix}-start.png` });
const before = await page.screenshot();

const box = await (await page.$("#view")).boundingBox();
const [cx, cy] = [box.x + box.width / 2, box.y + box.height / 2];
let old = await src();
await page.mouse.move(cx, cy);
await page.mouse.down();
await page.mouse.move(cx + 140, cy + 40, { steps: 10 });
await page.mouse.up();
await newFrame(old, "refined");
await page.screenshot({ path: `${prefix}-dragged.png` });
const dragged = await page.screenshot();
const result = { coarse_ms: coarseMs, refined_ms: refinedMs, drag_changed: !before.equals(dragged) };

if (timeFlag === "--time") {
  old = await src();
  const slider = await (await page.$("#time")).boundingBox();
  await page.mouse.click(slider.x + slider.width * 0.9, slider.y + slider.height / 2);
  await newFrame(old, "refined");
  await page.screenshot({ path: `${prefix}-time.png` });
  result.time = await page.$eval("#time", e => Number(e.value));
  result.time_changed = !dragged.equals(await page.screenshot());
}
console.log(JSON.stringify(result));
await browser.close();
