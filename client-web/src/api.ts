//! The gRPC-Web connection to cathlab-server: one Simulator client per token.
import { type Client, type Interceptor, createClient } from "@connectrpc/connect";
import { createGrpcWebTransport } from "@connectrpc/connect-web";
import { Simulator } from "./gen/cathlab/v1/simulator_pb.js";

export type SimulatorClient = Client<typeof Simulator>;

/** The server's base URL: `?server=` when given (a dev server elsewhere), else this page's origin. */
export function serverUrl(location: Location): string {
  const given = new URLSearchParams(location.search).get("server");
  return given && /^https?:\/\//.test(given) ? given.replace(/\/$/, "") : location.origin;
}

/** A client whose every call carries `authorization: Bearer <token>`. */
export function simulatorClient(baseUrl: string, token?: string): SimulatorClient {
  const bearer: Interceptor = (next) => async (request) => {
    if (token) request.header.set("authorization", `Bearer ${token}`);
    return next(request);
  };
  return createClient(
    Simulator,
    createGrpcWebTransport({ baseUrl, interceptors: [bearer], useBinaryFormat: true }),
  );
}
