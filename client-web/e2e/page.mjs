// Page helpers: reading frames, figures and layout off a page, and waiting for the next frame.

export const millimetres = (text) => Number.parseFloat(text);

/** A frame's pixels averaged over 8×8 blocks (quantum noise averages out, a moved wire not). */
export async function blocks(page, selector) {
  return page.$eval(selector, (img) => {
    const canvas = document.createElement("canvas");
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    const g = canvas.getContext("2d");
    g.drawImage(img, 0, 0);
    const { data, width, height } = g.getImageData(0, 0, canvas.width, canvas.height);
    const out = [];
    for (let by = 0; by + 8 <= height; by += 8)
      for (let bx = 0; bx + 8 <= width; bx += 8) {
        let sum = 0;
        for (let y = by; y < by + 8; y++) for (let x = bx; x < bx + 8; x++) sum += data[4 * (y * width + x)];
        out.push(sum / 64);
      }
    return out;
  });
}

export const largestChange = (a, b) => a.reduce((m, v, i) => Math.max(m, Math.abs(v - b[i])), 0);

/** The controls and HUD figures shown on `page` that lie outside its viewport (or have no
 *  width): their ids, or their first words. */
export async function outOfView(page) {
  return page.evaluate(() =>
    [...document.querySelectorAll("#controls button, #controls input, #controls select, #hud dd")]
      .filter((e) => e.checkVisibility())
      .map((e) => ({ id: e.id || e.textContent?.trim().slice(0, 20), r: e.getBoundingClientRect() }))
      .filter(({ r }) => r.bottom > innerHeight + 0.5 || r.right > innerWidth + 0.5 || r.width === 0)
      .map(({ id }) => id),
  );
}


/** Waits for a newer frame than the one `selector` shows now, loaded. */
export async function nextFrame(page, selector = "#xray") {
  const now = await page.$eval(selector, (img) => Number(img.dataset.frame ?? -1));
  await page.waitForFunction(
    ([s, n]) => {
      const img = document.querySelector(s);
      return Number(img?.dataset.frame ?? -1) > n && img.complete && img.naturalWidth > 0;
    },
    [selector, now],
    { timeout: 15_000 },
  );
}

/** The page's secrets in its address (after the page has run). */
export const secretsInAddress = (page) =>
  page.evaluate(() => ["account", "token", "key"].filter((k) => new URL(location.href).searchParams.has(k)));

/**
 * Waits until the page's session is connected; on a timeout the error says what the page
 * said instead (its connection state and message), so a failure names its cause.
 */
export async function connected(page, timeout) {
  try {
    await page.waitForSelector('#connection[data-status="connected"]', { timeout });
  } catch (e) {
    const status = await page.getAttribute("#connection", "data-status").catch(() => "?");
    const message = await page.textContent("#message").catch(() => "?");
    throw new Error(`not connected after ${timeout / 1000} s: status ${status}, message "${message}"\n${e.message}`);
  }
}
