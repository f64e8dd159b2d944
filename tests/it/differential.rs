use lobe as _;
