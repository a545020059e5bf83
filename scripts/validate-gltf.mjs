#!/usr/bin/env node
// Runs the Khronos glTF validator (npm package gltf-validator) on one .glb/.gltf file and prints
// its report as JSON on stdout. Exit status: 0 when the report has no errors, 1 when it has, 2
// when the validator cannot be loaded or run.
//
//   LFIT_GLTF_VALIDATOR=<npm prefix> node scripts/validate-gltf.mjs FILE
//
// The prefix is the one scripts/fetch-gltf-validator.sh prints (default
// ${LFIT_TOOLS_DIR:-$HOME/.cache/lfit-tools}/gltf-validator).
import { readFileSync } from "node:fs";
import { createRequire } from "node:module";
import { homedir } from "node:os";
import { basename, join } from "node:path";

const file = process.argv[2];
if (!file) {
    console.error("usage: node scripts/validate-gltf.mjs FILE.glb");
    process.exit(2);
}
const prefix = process.env.LFIT_GLTF_VALIDATOR
    || join(process.env.LFIT_TOOLS_DIR || join(homedir(), ".cache", "lfit-tools"), "gltf-validator");
let validator;
try {
    validator = createRequire(join(prefix, "node_modules", "noop.js"))("gltf-validator");
} catch (e) {
    console.error(`gltf-validator is not installed under ${prefix} (run scripts/fetch-gltf-validator.sh): ${e.message.split("\n")[0]}`);
    process.exit(2);
}
try {
    const report = await validator.validateBytes(new Uint8Array(readFileSync(file)), {
        uri: basename(file),
        maxIssues: 0,
        writeTimestamp: false,
    });
    console.log(JSON.stringify(report, null, 2));
    process.exit(report.issues.numErrors === 0 ? 0 : 1);
} catch (e) {
    console.error(`gltf-validator could not validate ${file}: ${e}`);
    process.exit(2);
}
