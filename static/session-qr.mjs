// A session's real-device page as a phone opens it, and that link as a QR code.
//
// The link is <origin>/xr#session=SID&token=TOKEN: the token travels in the fragment, which a
// browser never sends to the server, so it reaches no request line and no access log. The
// code is drawn by the vendored qrcode-generator into a GIF data URL, which the pages' CSP
// (img-src 'self' data:) allows; nothing is fetched.
import qrcode from "./vendor/qrcode-generator@2.0.4/dist/qrcode.mjs";

const ERROR_CORRECTION = "M"; // 15 % of the code may be unreadable (glare on a screen)
const QUIET_ZONE_MODULES = 4; // the light margin a QR code needs around it

/** `<origin>/xr#session=SID[&token=TOKEN]`: the token only when one is given. */
export function sessionPageUrl(origin, sid, token = "") {
  const fragment = new URLSearchParams({ session: sid });
  if (token) fragment.set("token", token);
  return `${origin}/xr#${fragment}`;
}

/** `text` (ASCII, as URLs are) as a QR code: a data: URL of a GIF, `modulePx` per module. */
export function qrDataUrl(text, modulePx = 3) {
  const code = qrcode(0, ERROR_CORRECTION); // 0: the smallest version that holds it
  code.addData(text, "Byte");
  code.make();
  return code.createDataURL(modulePx, QUIET_ZONE_MODULES * modulePx);
}
