//! Showing a session's X-ray frames in an <img>: a JPEG frame stream kept open, each frame
//! swapped in as a blob URL (the previous one released).
import type { SimulatorClient } from "./api.js";
import { FrameEncoding, type XrayFrame } from "./gen/cathlab/v1/simulator_pb.js";
import { type ConnectionStatus, keepOpen } from "./reconnect.js";

/** Streams JPEG frames of `size`×`size` pixels into `image` until `signal` aborts; marks the
 *  image with `data-frame` (the frame index) and calls `shown` for each frame. */
export function showFrames(
  client: SimulatorClient,
  sessionId: string,
  image: HTMLImageElement,
  options: { size: number; quality: number; signal: AbortSignal; shown?: (frame: XrayFrame) => void },
  status: (s: ConnectionStatus, detail?: string) => void = () => {},
): Promise<void> {
  let shownUrl = "";
  return keepOpen(
    async (received, signal) => {
      const frames = client.streamFrames(
        {
          sessionId,
          encoding: FrameEncoding.JPEG,
          width: options.size,
          height: options.size,
          jpegQuality: options.quality,
        },
        { signal },
      );
      for await (const frame of frames) {
        received();
        const url = URL.createObjectURL(new Blob([frame.data as Uint8Array<ArrayBuffer>], { type: "image/jpeg" }));
        image.src = url;
        if (shownUrl) URL.revokeObjectURL(shownUrl);
        shownUrl = url;
        image.dataset.frame = String(frame.index);
        options.shown?.(frame);
      }
    },
    status,
    options.signal,
  );
}
