// The trainee page on the one-device scene: connecting, fluoroscopy, the drive keys and
// buttons, a DSA run and the roadmap, and the layout at small screens.
import { join } from "node:path";
import { artifacts, assert } from "./harness.mjs";
import { blocks, largestChange, millimetres, nextFrame } from "./page.mjs";

export async function loadsAndConnects(ctx) {
  const { trainee, url } = ctx;
  // The one-device scene (the default is coaxial: the two-hand tests below take it).
  await trainee.goto(`${url}/?label=e2e-trainee&scene=arch_to_cow_lcca`);
  await trainee.waitForSelector('#connection[data-status="connected"]', { timeout: 30_000 });
  const sessionId = await trainee.$eval("body", (b) => b.dataset.session ?? "");
  ctx.sessionId = sessionId;
  assert(/^[0-9a-f-]{8,}$/.test(sessionId), `session id on the page: ${sessionId}`);
  assert((await trainee.textContent("#scene")).includes("arch_to_cow_lcca"), "scene name shown");
  assert((await trainee.$$eval("#device option", (o) => o.length)) === 3, "the scene's three devices listed");
  assert(new URL(trainee.url()).searchParams.get("session") === sessionId, "session kept in the URL for reloads");
  // Before the pedal: a prompt saying what to press, not a broken image.
  assert(await trainee.isVisible("#prompt"), "the fluoroscopy prompt shows before the pedal");
  assert((await trainee.textContent("#prompt")).includes("F"), "the prompt names the key");
  assert(!(await trainee.isVisible("#xray")), "no empty image before the first exposure");
  // The target is named with the distance still to go along the route.
  await trainee.waitForFunction(() => / mm$/.test(document.querySelector("#hud-target")?.textContent ?? ""), null, {
    timeout: 10_000,
  });
  const toGoAtStart = Number.parseFloat(/· ([0-9.]+) mm/.exec(await trainee.textContent("#hud-target"))?.[1] ?? "NaN");
  ctx.toGoAtStart = toGoAtStart;
  assert((await trainee.textContent("#hud-target")).startsWith("LCCA"), "the target named");
  assert(toGoAtStart > 100, `distance to go at the start: ${toGoAtStart} mm`);
}

export async function framesChangeAfterAPush(ctx) {
  const { trainee, toGoAtStart } = ctx;
  await trainee.bringToFront();
  await trainee.click("#screen"); // focus the page, not a form field
  await trainee.keyboard.down("f");
  await nextFrame(trainee);
  await nextFrame(trainee);
  const a = await blocks(trainee, "#xray");
  await nextFrame(trainee);
  const b = await blocks(trainee, "#xray");
  const noise = largestChange(a, b);
  const before = millimetres(await trainee.textContent("#hud-inserted"));
  await trainee.keyboard.down("ArrowUp");
  // The HUD's wall force while the shaped tip rides along the aortic wall.
  let wallForce = 0;
  for (let i = 0; i < 20; i++) {
    await trainee.waitForTimeout(100);
    wallForce = Math.max(wallForce, Number.parseFloat(await trainee.textContent("#hud-force")));
  }
  await trainee.keyboard.up("ArrowUp");
  await trainee.waitForTimeout(300);
  await nextFrame(trainee);
  await nextFrame(trainee);
  const c = await blocks(trainee, "#xray");
  const moved = largestChange(b, c);
  const after = millimetres(await trainee.textContent("#hud-inserted"));
  console.log(`  inserted ${before} → ${after} mm; largest 8×8-block change ${moved.toFixed(1)} grey levels (frame-to-frame noise ${noise.toFixed(1)})`);
  assert(after - before > 20 && after - before < 60, `↑ held 2 s at 20 mm/s advanced ${after - before} mm`);
  console.log(`  largest wall force on the HUD during the push: ${wallForce} mN`);
  assert(wallForce > 0, "the HUD shows the wall contact force");
  assert(moved > 3 * noise && moved > 10, `the image changed after the push: ${moved} vs noise ${noise}`);
  assert((await trainee.textContent("#mode")).startsWith("FLUORO"), "fluoroscopy mode shown");
  assert(!(await trainee.isVisible("#prompt")), "the prompt is gone once frames arrive");
  const dose = await trainee.textContent("#dose");
  console.log(`  dose display: ${dose}`);
  const kerma = Number.parseFloat(/Ka,r ([0-9.]+) mGy/.exec(dose)?.[1] ?? "NaN");
  assert(kerma > 0, `the dose display shows the accumulated reference air kerma: ${dose}`);
  // After ~40 mm of push the route to go is shorter (metrics come once a second).
  await trainee.waitForTimeout(1200);
  const toGo = Number.parseFloat(/· ([0-9.]+) mm/.exec(await trainee.textContent("#hud-target"))?.[1] ?? "NaN");
  console.log(`  to go: ${toGoAtStart} → ${toGo} mm`);
  assert(toGoAtStart - toGo > 15, `the distance to go fell by ${toGoAtStart - toGo} mm`);
  await trainee.screenshot({ path: join(artifacts, "trainee.png") });
  await trainee.keyboard.up("f");
}

export async function buttonsPullBack(ctx) {
  const { trainee } = ctx;
  const before = millimetres(await trainee.textContent("#hud-inserted"));
  const button = await trainee.$('#right-hand button[data-hold="pull"]');
  const box = await button.boundingBox();
  await trainee.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  await trainee.mouse.down();
  await trainee.waitForTimeout(1000);
  await trainee.mouse.up();
  await trainee.waitForTimeout(300);
  const after = millimetres(await trainee.textContent("#hud-inserted"));
  assert(before - after > 10, `the pull button withdrew ${before - after} mm`);
}

export async function keysDriveWithAControlFocused(ctx) {
  const { trainee } = ctx;
  for (const control of ["#primary", "#pulse"]) {
    await trainee.focus(control);
    const value = await trainee.$eval(control, (e) => e.value);
    const before = millimetres(await trainee.textContent("#hud-inserted"));
    await trainee.keyboard.down("ArrowUp");
    await trainee.waitForTimeout(1000);
    await trainee.keyboard.up("ArrowUp");
    await trainee.waitForTimeout(300);
    const after = millimetres(await trainee.textContent("#hud-inserted"));
    console.log(`  ${control} focused: ↑ moved the device ${before} → ${after} mm`);
    assert(after - before > 10, `↑ with ${control} focused advanced ${after - before} mm`);
    assert((await trainee.$eval(control, (e) => e.value)) === value, `${control} kept its value`);
    assert(await trainee.$eval(control, (e) => document.activeElement === e), `${control} kept the focus`);
  }
  await trainee.click("#screen");
}

export async function dsaRoadmapMarksTheTarget(ctx) {
  const { trainee } = ctx;
  await trainee.bringToFront();
  await trainee.click("#screen");
  await trainee.keyboard.down("f");
  await nextFrame(trainee);
  // A DSA run fires the injector after its mask; the contrast reaches the branches.
  await trainee.click("#dsa");
  await trainee.waitForFunction(() => document.querySelector("#mode")?.textContent?.startsWith("DSA"), null, {
    timeout: 15_000,
  });
  // A run of 8 s, as for an arch angiogram: the contrast rises from the descending aorta
  // through the arch into the branches.
  await trainee.waitForTimeout(8000);
  await trainee.click("#dsa");
  await trainee.click("#screen");
  await trainee.click("#roadmap");
  await trainee.waitForFunction(() => document.querySelector("#mode")?.textContent?.startsWith("ROADMAP"), null, {
    timeout: 15_000,
  });
  await nextFrame(trainee);
  await nextFrame(trainee);
  await trainee.waitForSelector('#target-marker[data-visible="true"]', { timeout: 10_000 });
  // Along the marked target (the LCCA from its origin on the arch) against the body
  // around it: the vessel map's contrast over the background noise.
  const measured = await trainee.evaluate(() => {
    const img = document.querySelector("#xray");
    const canvas = document.createElement("canvas");
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    const g = canvas.getContext("2d");
    g.drawImage(img, 0, 0);
    const { data, width, height } = g.getImageData(0, 0, canvas.width, canvas.height);
    const at = (x, y) => data[4 * (Math.round(y) * width + Math.round(x))];
    const points = document
      .querySelector("#target-marker polyline")
      .getAttribute("points")
      .trim()
      .split(/\s+/)
      .map((p) => p.split(",").map(Number))
      .map(([x, y]) => [x * width, y * height]);
    const inside = points.filter(([x, y]) => x >= 2 && y >= 2 && x < width - 2 && y < height - 2);
    const median = (v) => {
      const s = [...v].sort((a, b) => a - b);
      return s[Math.floor(s.length / 2)];
    };
    const vessel = median(inside.map(([x, y]) => at(x, y)));
    // Background: a ring 25–45 px round the marked vessel, 12 px or more from it.
    const near = (x, y, r) => inside.some(([px, py]) => (px - x) ** 2 + (py - y) ** 2 < r * r);
    const ring = [];
    for (let y = 0; y < height; y += 2)
      for (let x = 0; x < width; x += 2) if (near(x, y, 45) && !near(x, y, 25)) ring.push(at(x, y));
    const background = median(ring);
    const noise = 1.4826 * median(ring.map((v) => Math.abs(v - background)));
    return { points: inside.length, vessel, background, noise };
  });
  const ratio = Math.abs(measured.vessel - measured.background) / Math.max(measured.noise, 0.5);
  console.log(
    `  roadmap: ${measured.points} marker points; vessel ${measured.vessel} vs background ${measured.background} ± ${measured.noise.toFixed(2)} grey levels: contrast ${ratio.toFixed(1)}× the noise`,
  );
  await trainee.screenshot({ path: join(artifacts, "trainee-roadmap.png") });
  assert(measured.points >= 10, `the target marker has ${measured.points} points in the image`);
  assert(ratio >= 5, `the vessel map's contrast is ${ratio.toFixed(1)}× the background noise`);
  await trainee.click("#roadmap");
  await trainee.keyboard.up("f");
}

export async function layoutsFit(ctx) {
  const { trainee } = ctx;
  await trainee.bringToFront();
  for (const [width, height] of [[1280, 800], [1024, 640]]) {
    await trainee.setViewportSize({ width, height });
    await trainee.waitForTimeout(300);
    const layout = await trainee.evaluate(() => {
      const shown = [...document.querySelectorAll("#controls button, #controls input, #controls select, #hud dd")].filter(
        (e) => e.checkVisibility(),
      );
      const boxes = shown.map(
        (e) => {
          const r = e.getBoundingClientRect();
          return { id: e.id || e.textContent?.trim().slice(0, 20), bottom: r.bottom, right: r.right, width: r.width };
        },
      );
      const screen = document.querySelector("#screen").getBoundingClientRect();
      return {
        boxes,
        scroll: document.documentElement.scrollHeight - innerHeight,
        screen: { width: screen.width, height: screen.height },
      };
    });
    const outside = layout.boxes.filter((b) => b.bottom > height + 0.5 || b.right > width + 0.5 || b.width === 0);
    console.log(
      `  ${width}×${height}: image ${layout.screen.width.toFixed(0)}×${layout.screen.height.toFixed(0)} px; ${layout.boxes.length} controls, ${outside.length} out of view; page scrolls ${layout.scroll} px`,
    );
    await trainee.screenshot({ path: join(artifacts, `trainee-${width}x${height}.png`) });
    assert(outside.length === 0, `out of view at ${width}×${height}: ${JSON.stringify(outside)}`);
    assert(layout.scroll <= 0, `the page scrolls ${layout.scroll} px at ${width}×${height}`);
    assert(layout.screen.height >= height - 200, `the image uses the height: ${layout.screen.height} px`);
  }
  await trainee.setViewportSize({ width: 1280, height: 860 });
}
