// `vite build` writes the page into dist/, which gateway.js serves.
export default { base: './', build: { outDir: 'dist', emptyOutDir: true, chunkSizeWarningLimit: 1000 } };
