// The pages' credentials, this tab only (sessionStorage): the API key and each session's
// token, under keys the dashboard and the real-device page share, so a token given to one
// serves the other. A session's own token wins; the API key is accepted for every session.

const STORE_API_KEY = "semanticxr.apiKey";
const STORE_TOKENS = "semanticxr.tokens"; // {session id: token}

export const auth = {
  apiKey() {
    return sessionStorage.getItem(STORE_API_KEY) || "";
  },
  setApiKey(key) {
    if (key) sessionStorage.setItem(STORE_API_KEY, key);
    else sessionStorage.removeItem(STORE_API_KEY);
  },
  tokens() {
    try {
      const parsed = JSON.parse(sessionStorage.getItem(STORE_TOKENS) || "{}");
      return parsed && typeof parsed === "object" && !Array.isArray(parsed) ? parsed : {};
    } catch {
      return {};
    }
  },
  setToken(sid, token) {
    const tokens = auth.tokens();
    if (token) tokens[sid] = token;
    else delete tokens[sid];
    sessionStorage.setItem(STORE_TOKENS, JSON.stringify(tokens));
  },
  /** The credential for a session: its own token, else the API key ("" for none). */
  forSession(sid) {
    return (sid && auth.tokens()[sid]) || auth.apiKey();
  },
};
