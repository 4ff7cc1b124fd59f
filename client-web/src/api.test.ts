import { afterEach, describe, expect, it, vi } from "vitest";
import { AllowList, type TrustedServer, pageServer, simulatorClient } from "./api.js";

const PAGE = "http://127.0.0.1:50051";
const at = (search: string) => ({ origin: PAGE, search }) as Location;

/** A fetch that answers the allow-list with `origins` and counts its calls (and what they asked). */
function serve(origins: unknown, status = 200) {
  const calls: string[] = [];
  vi.stubGlobal("fetch", async (input: string) => {
    calls.push(String(input));
    return new Response(JSON.stringify(origins), { status });
  });
  return calls;
}

afterEach(() => {
  vi.unstubAllGlobals();
  vi.useRealTimers();
});

describe("pageServer", () => {
  it("is this origin without ?server=, asking nothing", async () => {
    const calls = serve({ origins: [] });
    expect(await pageServer(at(""))).toMatchObject({ ok: true, base: PAGE, param: null });
    expect(await pageServer(at(`?server=${encodeURIComponent(`${PAGE}/`)}`))).toMatchObject({ ok: true, param: null });
    expect(calls).toEqual([]);
  });
  it("takes a listed server, asking this origin's list only", async () => {
    const calls = serve({ origins: ["http://10.0.0.2:7000"] });
    const got = await pageServer(at("?server=http://10.0.0.2:7000/"));
    expect(got).toMatchObject({ ok: true, base: "http://10.0.0.2:7000", param: "http://10.0.0.2:7000" });
    expect(calls).toEqual(["/fleet-origins"]);
  });
  it("refuses a server not listed, or when the list cannot be read", async () => {
    serve({ origins: ["http://10.0.0.2:7000"] });
    const got = await pageServer(at("?server=http://127.0.0.1:9"));
    expect(got.ok).toBe(false);
    if (!got.ok) expect(got.message).toMatch(/Nothing was sent/);
    serve("not found", 404);
    expect((await pageServer(at("?server=http://10.0.0.2:7000"))).ok).toBe(false);
    vi.stubGlobal("fetch", async () => {
      throw new TypeError("network");
    });
    expect((await pageServer(at("?server=http://10.0.0.2:7000"))).ok).toBe(false);
  });
});

describe("AllowList", () => {
  it("trusts this origin without asking, and a fleet server once listed (read again at most every 5 s)", async () => {
    vi.useFakeTimers({ toFake: ["Date"] });
    const list = new AllowList(PAGE);
    let calls = serve({ origins: [] });
    expect(await list.trust(`${PAGE}/x`)).toBe(PAGE);
    expect(calls).toEqual([]);
    expect(await list.trust("http://10.0.0.3:7000")).toBeUndefined();
    expect(await list.trust("http://10.0.0.3:7000")).toBeUndefined();
    expect(calls).toHaveLength(1);
    // The server joins the fleet; the list is read again after 5 s.
    calls = serve({ origins: ["http://10.0.0.3:7000"] });
    expect(await list.trust("http://10.0.0.3:7000")).toBeUndefined();
    vi.setSystemTime(Date.now() + 5001);
    expect(await list.trust("http://10.0.0.3:7000/")).toBe("http://10.0.0.3:7000");
    expect(calls).toHaveLength(1);
    expect(await list.trust("javascript:alert(1)")).toBeUndefined();
  });
});

describe("simulatorClient", () => {
  it("refuses a base that was not trusted", () => {
    expect(() => simulatorClient("http://127.0.0.1:9" as TrustedServer, "secret")).toThrow(/not a server/);
  });
});
