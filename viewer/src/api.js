// Data requests: the run's files, with a bearer key kept in sessionStorage (never in a URL).

const KEY = "dcseg.apiKey";

export class AuthError extends Error {}

function headers() {
  const key = sessionStorage.getItem(KEY);
  return key ? { Authorization: `Bearer ${key}` } : {};
}

async function problem(response, url) {
  let detail = response.statusText;
  try {
    const body = await response.json();
    detail = body.detail ?? body.title ?? detail;
  } catch {
    // not JSON: keep the status text
  }
  return `GET ${url}: ${response.status} ${detail}`;
}

/** GET `url`; resolves to the response or throws AuthError (401/403) or Error (other status). */
export async function get(url) {
  const response = await fetch(url, { headers: headers(), cache: "no-store" });
  if (response.status === 401 || response.status === 403) {
    throw new AuthError(await problem(response, url));
  }
  if (!response.ok) throw new Error(await problem(response, url));
  return response;
}

/** Ask for an API key with the page's form; resolves once one is stored. */
export function askForKey(message) {
  const form = document.getElementById("key-form");
  const input = document.getElementById("key-input");
  document.getElementById("key-message").textContent = message;
  form.hidden = false;
  input.focus();
  return new Promise((resolve) => {
    form.onsubmit = (event) => {
      event.preventDefault();
      sessionStorage.setItem(KEY, input.value.trim());
      input.value = "";
      form.hidden = true;
      resolve();
    };
  });
}

/** Fetch every url (a map of name to url) with the key, asking for one while refused. */
export async function fetchAll(urls) {
  for (;;) {
    try {
      const entries = await Promise.all(
        Object.entries(urls).map(async ([name, url]) => [name, await get(url)]),
      );
      return Object.fromEntries(entries);
    } catch (error) {
      if (!(error instanceof AuthError)) throw error;
      sessionStorage.removeItem(KEY);
      await askForKey(`${error.message}. Enter an API key (kept in this tab only).`);
    }
  }
}
