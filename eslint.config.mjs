// The linter of web/: the pages' ES modules, run in the browser as they are (no build).
// eslint:recommended, browser globals only (no-undef), and no hidden globals: modules talk
// through imports and window events; window.fpvDebug is the tests' view of a page, written
// only by web/debug.js and read by no module.
import js from "@eslint/js";
import globals from "globals";

export default [
  js.configs.recommended,
  {
    files: ["web/**/*.js"],
    languageOptions: {
      ecmaVersion: 2024,
      sourceType: "module",
      globals: globals.browser,
    },
    rules: {
      "no-implicit-globals": "error",
      "no-undef": "error",
      "no-unused-vars": ["error", { caughtErrors: "none" }],
      "no-restricted-properties": [
        "error",
        { object: "window", property: "fpv", message: "import the module that owns it" },
        { object: "window", property: "fpvDebug", message: "tests' view only: debug.js expose()" },
      ],
      "no-restricted-globals": [
        "error",
        { name: "fpv", message: "import the module that owns it" },
        { name: "fpvDebug", message: "tests' view only: debug.js expose()" },
      ],
    },
  },
  {
    // A module worker (web/video.js starts it): a worker's globals, not a window's.
    files: ["web/video-worker.js"],
    languageOptions: { globals: globals.worker },
  },
  {
    files: ["web/debug.js"],
    rules: { "no-restricted-properties": "off" },
  },
];
